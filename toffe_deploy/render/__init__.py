"""What people look at: frames, videos and the HTML report of a run, and `dataset show` panels.

One drawing style for every picture (issue 15):

- ``draw``: pure numpy / OpenCV functions on a BGR image: the palette (flow colour wheel, hue =
  direction, readable on dark and light backgrounds), event images, arrows, trails, dashed
  ground-truth outlines, labels placed beside objects, the colour-wheel legend, a whole frame;
- ``truth``: the ground-truth outline of each generated object (shape and size from the
  recording's attrs);
- ``video``: frame sinks (a PNG folder, an H.264 MP4 through PyAV), staged and checked so nothing
  partial is left;
- ``frames``: ``run --render`` (track trails across windows, ground truth, a sink);
- ``report``: ``run --report FILE.html``, one self-contained page.
"""
