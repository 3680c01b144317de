"""localize: sessions, inertial odometry (PDR, RoNIN) and the map-aware particle filter."""
