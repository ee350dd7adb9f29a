"""Motion Composer's application layer: the command line (`app.cli`) and the Qt window (`app.gui`)."""
