"""Detectors on real-looking images (BallFinder on stereo depth, the sandal board) and their renderers."""
