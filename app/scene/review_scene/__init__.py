"""One browser's 3-D scene of a robot (or every browser's): a review's two copies and their marks, a robot shown
alone, or Observe's live robot. ReviewScene (scene.py) holds what is shown and selected; its parts draw the robot's
copies (copies.py) and the marks (marks.py) into the nodes it keeps (nodes.py), place them in the world
(layout.py) and aim the cameras (camera.py)."""
