"""Stability control: yaw-rate reference, direct yaw-moment laws, torque allocation, 4WS."""
