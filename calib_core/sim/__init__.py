"""The simulated robot: hidden true parameters, realistic noise, rendered images."""
