"""Geometry: rigid transforms, planar polygons and polyhedral solids."""
