"""How the camera moves along the road: ``speed`` (cruise, smooth variation and stops over time)
and ``trajectory`` (the camera's poses, and the noisy GPS a cheap receiver logs on them)."""
