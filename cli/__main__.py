"""`python -m cli`: the `m3gd` command line."""

from cli.app import app

app()
