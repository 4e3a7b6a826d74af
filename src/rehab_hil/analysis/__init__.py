"""Analyses of simulated or measured runs against the seed papers (seed 000 eq 29-30, Fig. 10, 15-16)."""
