"""The HTTP service: ``api`` (routes, uploads, auth), ``jobs`` (the job's life cycle and workers),
``map`` (fusion jobs and the map routes), ``admin`` (the dashboard), and here its startup checks
and the S3-compatible bundle store."""
