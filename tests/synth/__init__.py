"""The synthetic journey generator (``app.synth``): determinism, renders against the camera model,
detections and trajectories against the truth, the bundle against the contract, and the corpus."""
