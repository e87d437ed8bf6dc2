"""Traffic capture: the file formats every frame of a connection is kept in, and their readers.

``jsonl`` (the JSON Lines capture, the writer interface the driver feeds, replay), ``part`` (a
connection's binary capture part), ``mcap_writer`` (the run's ``capture.mcap``), ``append``
(an attachment added to a finished file), ``mcap_walk`` (an MCAP file's records, checked),
``read`` (one reader for either format) and ``tally`` (what a capture's traffic adds up to).

Below the driver, which writes captures and replays them, and above the codec and the robot
model it encodes; the report and calibration read captures through it. Importing the package
imports none of its modules.
"""
