%
O1001 (SEAM - weld seam along a bracket edge: two lines, two arcs)
(units mm, absolute coordinates, XY plane; the seam lies at Z = 5.08)
N10 G21 G90 G17 ; millimetres, absolute, XY plane
N20 G0 Z25.4           (safe height)
N30 G0 X0 Y0           (approach above the start)
N40 G0 Z5.08
N50 G1 X101.6 F600     (first straight, +X)
N60 G2 X152.4 Y-50.8 I0 J-50.8   (clockwise quarter circle, centre 101.6 -50.8, R 50.8)
N70 G1 Y-101.6         (straight, -Y)
N80 G3 X203.2 Y-152.4 R50.8      (counter-clockwise quarter circle, centre 203.2 -101.6)
N90 G1 X254.0
N100 X304.8            ; modal G1: straight on to the end
N110 G0 Z25.4          (retract)
N120 M30
%
