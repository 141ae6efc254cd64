"""Measurement models: what a sensor reports for a point on the robot, with exact derivatives and noise."""
