"""ovrad's user interface: the sidebar panel in the 3D view."""
