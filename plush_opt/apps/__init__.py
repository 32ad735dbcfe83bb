"""Applications at the edge: command line, posing window, scripted runs, comparison, benchmarks, plots."""
