"""Stage 2 (paper Sec. III-C): LSTM refinement of every demo with an adaptive β."""
