"""The paper's evaluation (Sec. IV): imitation learners trained on noisy vs cleaned demos, the
protocol that compares them, and ``bt reproduce``."""
