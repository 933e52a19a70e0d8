"""``feeder tune``: search a scenario's settings for the best mean parts/min (Optuna)."""
