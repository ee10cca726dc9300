"""Furniture: desk, sofa, chair, stair, table."""
