"""``python -m ekfviz`` runs the command line."""

from ekfviz.cli import app

app(prog_name="ekfviz")
