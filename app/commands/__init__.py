"""The ``signmap`` subcommands, one module per group: they parse arguments and call the
pipeline, the synthetic generator, the service or the benches; no maths and no routes here."""
