"""Load benchmarks of the service on 127.0.0.1: the HTTP API under concurrent uploads and reads
(``signmap bench api``), map pages and tiles at scale (``signmap bench map``), the admin
dashboard and hostile uploads, and the real ``signmap serve`` processes they run against.
"""
