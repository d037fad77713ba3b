"""Video journeys: container checks, NMEA and embedded GPS, the clock offset between camera and
GPS, frame choice, and whole video journeys through the CLI."""
