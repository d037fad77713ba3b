"""Studies: one question each, asked of corpus journeys (drawn without pixels, rendered, or kept
from a corpus run) or of a real drive: the turn finder, GPS scale and noise draws, a focal check
from GPS, where a sign's error comes from, ego-motion on real imagery, render fidelity and the
sign-uncertainty knob fit.
"""
