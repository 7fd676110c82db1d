"""Training loops, evaluation and schedules."""
