"""Rerun blueprints (the live, inspect and compare layouts arrive with the dashboard)."""
