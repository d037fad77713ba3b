"""A video journey (wire contract section 1a): the container's header, its GPS (an NMEA log, a GPX
track, gps.csv or the video's own GPMF/CAMM track), the clock offset between camera and GPS, and
the frames the pipeline keeps, decoded as a stream.
"""
