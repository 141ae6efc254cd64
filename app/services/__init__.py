"""What the desk does beyond storing, one service a module, below the routers and above the store: apply a
calibration (apply.py, through the gate of safety.py), calibrate (calibration.py), replay and dry runs
(replay.py), review (review.py), the robot in view and Observe (connection.py, observe.py's live loop), driving a
robot at once (drive.py) and adding or removing robots (robots.py)."""
