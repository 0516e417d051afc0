"""Closed-loop camera simulator: HDR scenes, DVS events, APS frames that obey exposure commands."""
