"""The scan format: posed frames plus a triangle mesh (see ``docs/formats.md``)."""

from reroom.scan.camera import Frame, Intrinsics, look_at
from reroom.scan.scan import Scan, load_scan, validate_pose, write_scan

__all__ = ["Frame", "Intrinsics", "Scan", "load_scan", "look_at", "validate_pose", "write_scan"]
