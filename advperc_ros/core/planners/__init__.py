"""Motion planners and the plug-in protocol they share."""
