"""The terminal UI of the instrument (``bodebench tui``): a bench session watched and steered from a terminal."""

from bodebench.apps.tui.app import BodeBenchApp, run_tui

__all__ = ["BodeBenchApp", "run_tui"]
