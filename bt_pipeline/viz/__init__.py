"""Output at the edges: Rerun logging, matplotlib figures and rich tables / JSON reports."""
