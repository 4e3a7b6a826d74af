"""Discrepancy workflow: replay measured inputs, localise the residual, name and fit the missing
effect, and report the gap before and after (docs/discrepancy.md)."""
