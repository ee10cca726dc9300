"""Utensils: fork."""
