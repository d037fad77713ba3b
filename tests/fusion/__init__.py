"""Fusing journeys' signs into one map (``app.fusion``): order independence, accuracy, close signs,
the robust mean and its covariance floor, and change detection."""
