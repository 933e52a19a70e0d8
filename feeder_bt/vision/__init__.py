"""Vision: recipes that turn pixels into part poses (OpenCV)."""
