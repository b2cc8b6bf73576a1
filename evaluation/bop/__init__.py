"""The BOP challenge's scoring: results files (`csv`), recall and AR from per-target errors (`recall`), and
the service protocol's answers scored so (`scores`)."""
