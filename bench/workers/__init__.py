"""Worker processes for trials measured in parallel: the process side, which imports nothing of the
runner so that a worker starts fast. Importing the package imports none of its modules."""
