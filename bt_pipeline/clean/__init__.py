"""The two-stage cleaner (paper Sec. III-B/C, Algorithm 1): ``stage1/`` extracts the canonical
motion of the best demo, ``stage2/`` refines every demo; ``pipeline`` runs both on one task and
``driver`` runs them over files. Torch is imported only by ``stage2``."""
