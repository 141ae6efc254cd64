"""What the browser sees of a robot: each tab's viewer (viewers.py) and its 3-D scene in viser (review_scene/),
where that scene's camera stands (framing.py), the robot drawn there (robot_copy.py, from robot_look.py's visuals),
how the viser client looks (theme.py), the review computed for the scene and the 2-D views (review.py), Observe's
2-D view (live_look.py), and the one module that uses viser's private names (viser_private.py)."""
