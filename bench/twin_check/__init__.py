"""``armbench twin-check``: how well the twin predicts an arm's capture, and what to do when it
does not. Importing the package imports none of its modules."""
