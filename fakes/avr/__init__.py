"""The firmware in the loop: the reference firmware on simavr, the ``avr://`` transport and the
differential check against the emulator. Importing the package imports none of its modules."""
