"""Every plot, drawn once with matplotlib and shown by both the report (SVG) and the studio (RGB image): one
module per problem (:mod:`.intrinsics`, :mod:`.multicam`, :mod:`.rig`), the style and the two outputs in
:mod:`.render`. Each function takes plain records or arrays and returns a :class:`matplotlib.figure.Figure`."""
