"""The repository as a whole: the import layers and package sizes, the ``signmap`` command line as a
user meets it, the scripts, docker-compose, the docs' links, and what the end of a test run says."""
