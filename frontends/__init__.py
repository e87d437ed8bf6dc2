"""Front ends beside the command line: the arm served as a ROS 2 node and live in Foxglove.
Importing the package imports none of its modules."""

if __name__ != "armbench.frontends":  # the checkout's folder by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.frontends: import it by that name")
