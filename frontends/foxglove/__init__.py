"""Live view in Foxglove. Importing the package imports none of its modules."""
