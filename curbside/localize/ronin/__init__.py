"""RoNIN learned inertial odometry: model, training data, training loop and inference.

- :mod:`~curbside.localize.ronin.model` -- RoNIN-ResNet and its compact variant;
- :mod:`~curbside.localize.ronin.data` -- recordings from MS Indoor 2020, IPIN 2023 and the RoNIN HDF5
  layout, weak velocity labels from waypoints, windows;
- :mod:`~curbside.localize.ronin.train` -- the seeded, resumable training loop;
- :mod:`~curbside.localize.ronin.stream` -- :class:`RoninStream`, IMU rows in any chunking to model windows;
- :mod:`~curbside.localize.ronin.infer` -- :func:`infer_windows` (fixed-shape batches) and
  :func:`ronin_velocity`, ``imu.csv`` to ``velocity.csv``;
- :mod:`~curbside.localize.ronin.evaluate` -- distance ratio, speed error, ATE and RTE.
"""
