"""Deprecated alias of the `m3gd` app, which lives in the command layer `cli.app`.

Kept so `python -m pipeline.cli` and `from pipeline.cli import app` keep working; new code
imports `cli.app`. The one import from pipeline/ up into the command layer (exempted in the
layering contract).
"""

from cli.app import app

__all__ = ["app"]

if __name__ == "__main__":
    app()
