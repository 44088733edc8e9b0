%
(seam_inch_relative.nc - the same seam as seam.nc, in inches and relative moves)
N10 G20 G91 G17 ; inches, incremental, XY plane
N20 G0 Z1.0            (safe height)
N30 G0 X0 Y0           (no move)
N40 G0 Z-0.8           (down to Z 0.2 in = 5.08 mm)
N50 G1 X4.0 F24
N60 G2 X2.0 Y-2.0 I0 J-2.0       (centre offsets from the start point)
N70 G1 Y-2.0
N80 G3 X2.0 Y-2.0 R2.0
N90 G1 X2.0
N100 X2.0              ; modal G1
N110 G0 Z0.8
N120 M30
%
