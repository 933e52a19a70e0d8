"""The simulated cell: world, devices and rendered camera images, on the clock."""
