"""Virtual time: the event loop that runs the bench against emulated targets without waiting.
Importing the package imports none of its modules."""
