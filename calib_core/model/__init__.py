"""The robot model: profiles (YAML or URDF) compiled to frames of elementary transforms, and their kinematics."""
