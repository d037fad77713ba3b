"""What a camera's journeys tell of it, beyond one journey's self-calibration: a stored
calibration checked on a later journey's turn (``check_on_turn``), and the camera calibrated
jointly from all its journeys' turn windows (``calibrate_jointly``, which the service runs).
"""
