"""Command line: argument parsing of every `testbed` command; the work is done by the stages."""
