"""Command-line tools of the simulators."""
