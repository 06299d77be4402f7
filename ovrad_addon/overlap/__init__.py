"""The overlap matrix C: the patches' contacts and visibility, the quadrature of their supports,
C's assembly, point queries (alpha at surface points, ray hits) and the blocks of C kept on an atlas."""
