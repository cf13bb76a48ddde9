"""Helpers shared by the tests and the benchmarks (neither imports the other's helpers):
small random hybrid models and burst inputs (:mod:`testkit.synthetic`)."""
