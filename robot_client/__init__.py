"""Real-robot client: Kobuki driver, AprilTag + odometry localisation, action runner."""
