"""The HTTP API's routes against the real app: uploads and their bad input, the read routes'
shapes, every route under every kind of caller, and schemathesis over the OpenAPI schema."""
