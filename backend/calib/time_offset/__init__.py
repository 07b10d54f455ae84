"""Time offsets between two sensors' clocks, from one motion both see.

- :mod:`.signals`: what each sensor gives as its motion over time (the board's normal, angular rates, the board's
  line in a 2D scanner's plane: :mod:`.scan_line`);
- :mod:`.alignment`: the offset, with its sigma, that best lines the two signals up;
- :mod:`.checks`: the verdict (the offset's sigma, the two halves of the recording);
- :mod:`.service`: the session's sensors, their captures, the stored result and its accept (the sensor's clock
  offset in the rig).
"""
