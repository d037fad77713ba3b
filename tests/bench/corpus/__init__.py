"""The corpus bench: its runner, records and reports on hand-made and tiny rendered corpora, as
frames bundles and as dash cam video bundles."""
