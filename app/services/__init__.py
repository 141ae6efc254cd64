"""What the desk does with its robots beyond storing: apply a calibration (the gate), replay, observe, review."""
