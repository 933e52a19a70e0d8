"""Protocol emulators of the cell's controllers, backed by the simulated cell in real time."""
