"""The database: the ORM rows (``models``, each class named ``...Row``), engines and sessions
(``session``), row updates shared by the API, the dashboard and the jobs (``crud``), reads as GeoJSON
(``queries``), the map's heavy reads and tiles (``map_read``, ``map_tiles``) and conversions between
rows and the fusion's domain values (``map_rows``). The schema itself is made by ``migrations/``."""
