"""Command-line tools of the offline analysis (``python -m terrain_analysis.tools.<name>``)."""
