"""Slow, obviously correct reference implementations (plain loops), one module per shipped module
they check: the tests compare the fast code with them. Nothing in the library imports this package."""
