"""Journey jobs: their life cycle in the database, the embedded worker, what crashes leave behind,
and the per-stage report kept with each journey."""
