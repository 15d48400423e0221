"""`python -m bridge` runs the `gx3` command line."""

from bridge.cli import app

app()
