"""Trackers: slots, the networks' input features (``features``), and the tracker
layouts with the model that serves each (``layouts``: the one ``Layout`` enum)."""
