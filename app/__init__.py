"""rangereg's front ends: the command line and the viser workbench, thin layers over ``core``."""
