"""Files in and out: the CSV data formats, session folders, ROS bags, the CTU data set, driver exports.

The names below load their module on first use (calib_core/_lazy.py): rosbags only for `import_bag`."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_exports

__getattr__ = lazy_exports(
    __name__,
    {
        "bag_import": ("import_bag",),
        "bag_tf": ("handeye_folder_from_bag",),
        "camera_images": ("NAOQI_COLOR_SPACES", "grey_image", "naoqi_image"),
        "csv_format": (
            "measurement_values",
            "parse_dataset",
            "plan_csv",
            "read_dataset",
            "readings_beyond_limits",
            "select_rows",
            "to_csv",
        ),
        "ctu_motoman": ("camera_dataset",),
        "export": (
            "bhuman_joint_calibration",
            "calibrated_links",
            "calibrated_urdf",
            "estimated_offsets_deg",
            "offsets_yaml",
        ),
        "flange_poses": ("BoardSpec", "Camera", "parse_board", "read_camera", "read_flange_poses"),
        "flange_export": ("flange_calibration_json",),
        "flange_session": ("FlangeSession", "flange_pose_session", "write_flange_session"),
        "handeye_export": ("HANDEYE_FORMATS", "export_handeye", "read_handeye"),
        "ros_tf": ("FRAME_NAME", "LinkPose", "StaticTransform", "link_poses", "static_tf_launch"),
        "session": ("FrameRecord", "csv_sensors", "parse_measured", "read_session", "session_robot", "write_session"),
        "urdf_export": ("BODY", "to_urdf"),
    },
)
__all__ = [
    "BODY",
    "FRAME_NAME",
    "HANDEYE_FORMATS",
    "NAOQI_COLOR_SPACES",
    "BoardSpec",
    "Camera",
    "FlangeSession",
    "FrameRecord",
    "LinkPose",
    "StaticTransform",
    "bhuman_joint_calibration",
    "calibrated_links",
    "calibrated_urdf",
    "camera_dataset",
    "csv_sensors",
    "estimated_offsets_deg",
    "export_handeye",
    "flange_calibration_json",
    "flange_pose_session",
    "grey_image",
    "handeye_folder_from_bag",
    "import_bag",
    "link_poses",
    "measurement_values",
    "naoqi_image",
    "offsets_yaml",
    "parse_board",
    "parse_dataset",
    "parse_measured",
    "plan_csv",
    "read_camera",
    "read_dataset",
    "read_flange_poses",
    "read_handeye",
    "read_session",
    "readings_beyond_limits",
    "select_rows",
    "session_robot",
    "static_tf_launch",
    "to_csv",
    "to_urdf",
    "write_flange_session",
    "write_session",
]

if TYPE_CHECKING:
    from .bag_import import import_bag
    from .bag_tf import handeye_folder_from_bag
    from .camera_images import NAOQI_COLOR_SPACES, grey_image, naoqi_image
    from .csv_format import (
        measurement_values,
        parse_dataset,
        plan_csv,
        read_dataset,
        readings_beyond_limits,
        select_rows,
        to_csv,
    )
    from .ctu_motoman import camera_dataset
    from .export import (
        bhuman_joint_calibration,
        calibrated_links,
        calibrated_urdf,
        estimated_offsets_deg,
        offsets_yaml,
    )
    from .flange_export import flange_calibration_json
    from .flange_poses import BoardSpec, Camera, parse_board, read_camera, read_flange_poses
    from .flange_session import FlangeSession, flange_pose_session, write_flange_session
    from .handeye_export import HANDEYE_FORMATS, export_handeye, read_handeye
    from .ros_tf import FRAME_NAME, LinkPose, StaticTransform, link_poses, static_tf_launch
    from .session import FrameRecord, csv_sensors, parse_measured, read_session, session_robot, write_session
    from .urdf_export import BODY, to_urdf
