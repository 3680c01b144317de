"""evaluate: ground truth, the paper's metrics, simulation, reports and map-source comparison."""
