"""Uploads against the real app: the contract's broken bundles, hostile and extreme ones, what an
upload may cost the API, the per-key limits, and outages (database, disk) that must leave nothing."""
