"""The robots on the desk: which ones it starts with (desk_config.py), each an instance of a profile with its own
driver or none (roster.py), the meshes a robot added from a profile file brings along (profile_meshes.py), and
capturing frames through a robot's driver into its sessions (capture.py). The drivers themselves are app/drivers/."""
