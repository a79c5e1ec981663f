"""Importers: turn other capture formats into reroom scans.

:mod:`reroom.importers.rgbd` fuses posed RGB-D sequences (TSDF, Open3D);
:mod:`reroom.importers.preview` renders a quick picture of an imported mesh.
Open3D and Mitsuba are imported only when a function needs them.
"""

from reroom.importers.preview import overview_camera, render_mesh_preview
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
    "overview_camera",
    "read_depth",
    "read_intrinsics",
    "read_pose_file",
    "render_mesh_preview",
    "white_border_mask",
]
