"""The twin: the arm's physics, its joints and their stepper drives. Importing the package imports
none of its modules."""
