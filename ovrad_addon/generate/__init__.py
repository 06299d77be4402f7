"""Making atlases: placing disks and squares on planar and curved sheets, building an atlas and its
C in one go, and adaptive refinement of patches from a solve."""
