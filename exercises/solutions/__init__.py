"""The reference answers of the exercises, self-contained, equal to the project's functions."""
