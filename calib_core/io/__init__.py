"""Files in and out: the CSV data formats, session folders, ROS bags, the CTU data set, driver exports."""
