"""Thin rclpy nodes (driver, compensator, trajectory, recorder): they map topics and parameters to core objects."""
