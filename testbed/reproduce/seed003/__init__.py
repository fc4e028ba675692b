"""Paper 003: symmetric measurement equations for crossing point targets."""
