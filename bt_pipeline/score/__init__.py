"""Scoring (paper Sec. III-A): KSG mutual information, task losses L1-L3, the demo utility score Ũ
and best-demo selection."""
