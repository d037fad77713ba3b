"""The fused map: fusion jobs on SQLite and PostgreSQL, the map routes (filters, paging, evidence,
changes, tiles), two workers fusing at once, and the map at scale."""
