"""Importers: turn other capture formats into reroom scans.

:mod:`reroom.importers.rgbd` fuses posed RGB-D sequences (TSDF, Open3D);
:mod:`reroom.importers.preview` renders a quick picture of an imported mesh.
"""

from reroom.importers.rgbd import (
    estimate_up,
    find_rgbd_folder,
    import_rgbd,
    import_rgbd_folder,
    read_depth,
    read_intrinsics,
    read_pose_file,
    white_border_mask,
)

__all__ = [
    "estimate_up",
    "find_rgbd_folder",
    "import_rgbd",
    "import_rgbd_folder",
    "read_depth",
    "read_intrinsics",
    "read_pose_file",
    "white_border_mask",
]
