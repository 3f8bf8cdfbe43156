"""Event-bin source: feeds host-binned windows into the network one time bin per step."""
