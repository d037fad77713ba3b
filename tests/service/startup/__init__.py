"""The service's start: what `signmap serve` and `signmap worker` check before they answer or
take jobs (database, migrations, data_dir, detector), and what they print when they refuse."""
