"""Pictures for people: contact sheets of frames (more views come with later stages)."""

from reroom.viz.contact_sheet import contact_sheet

__all__ = ["contact_sheet"]
