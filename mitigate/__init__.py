"""Stick-slip mitigation: controllers, closed loop, scenario runner, metrics, plots and the CLI."""
