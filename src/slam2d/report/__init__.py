"""Pictures and reports people look at."""
