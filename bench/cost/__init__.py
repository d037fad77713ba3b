"""Costs: what one of the worker's own steps costs per unit of input, timed against a baseline
measured in the same run (a ratio, so the machine's speed cancels): the sign detector's time per
frame (``signmap bench detector``, ``detector_time``).
"""
