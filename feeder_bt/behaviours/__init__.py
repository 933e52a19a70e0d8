"""Leaves of the four trees. They see the HAL interfaces and the context, never a driver."""
