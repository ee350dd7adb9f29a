"""Motion Composer's application layer: the command line and (later) the Qt window."""
