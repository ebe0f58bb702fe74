"""Worlds and geometry: shapes, the world and its document section, the labels L(x), random
obstacles, Dubins paths and drivable guides."""
