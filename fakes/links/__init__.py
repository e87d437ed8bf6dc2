"""The host's ends of an emulated arm: ``fake://`` in process, a pseudo-terminal or a TCP port
served in real time. Importing the package imports none of its modules."""
