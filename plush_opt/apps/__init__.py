"""Applications at the edge: command line, posing window, scripted runs, comparison, benchmarks,
plots, export. Everything below is theirs to import; nothing imports them."""
