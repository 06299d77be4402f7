"""The operators' poll checks: the first check that fails tells Blender why the operator is greyed out."""

from __future__ import annotations

from . import attributes


def passes(cls, checks) -> bool:
    """Whether every (ok, message) check holds; the first one that fails sets its poll message."""
    for ok, message in checks:
        if not ok:
            cls.poll_message_set(message)
            return False
    return True


def object_mode(context, action: str) -> tuple[bool, str]:
    """The check that Blender is in Object Mode, for an operator that does `action`."""
    return context.mode == "OBJECT", f"Switch to Object Mode to {action}"


def selected_meshes(context) -> list:
    """The selected mesh objects that are not atlas objects."""
    return [o for o in context.selected_objects if o.type == "MESH" and not attributes.is_atlas(o)]
