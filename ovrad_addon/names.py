"""Names of every attribute, property and data block ovrad writes into a Blender file."""

# POINT attributes on an atlas object (one point per patch).
NORMAL = "ovrad_normal"  # FLOAT_VECTOR, unit normal of the patch plane
RADIUS = "ovrad_radius"  # FLOAT, disk radius or half the side of a square
SHAPE = "ovrad_shape"  # INT, 0 disk, 1 square, 2 ball (clutter.py)
TANGENT = "ovrad_tangent"  # FLOAT_VECTOR, first in-plane axis (a square's side direction)
AREA = "ovrad_area"  # FLOAT, effective area c_kk = integral of alpha_k over the surface
OVERLAP = "ovrad_overlap"  # INT, how many other patches overlap this one
SHEET = "ovrad_sheet"  # INT, surface sheet (chart and side) the patch lies on
THICKNESS = "ovrad_thickness"  # FLOAT, tolerated distance from the patch plane
MIN_COS = "ovrad_min_cos"  # FLOAT, least cosine between patch and surface normals
SUPPORT_AREA = "ovrad_support_area"  # FLOAT, area A_h of the patch's support on the surface
TRIANGLE = "ovrad_triangle"  # INT, a triangle of the patch's sheet, counted in its source object's triangles
# FLOAT_VECTOR, the point on the sheet the patch sees its support from (overlap/contacts.py)
ANCHOR = "ovrad_anchor"
SIDE = "ovrad_side"  # INT, side of that triangle the patch lies on: +1 front, -1 back
OBJECT = "ovrad_object"  # INT, environment atlas only: the surfaces object each patch lies on
RANDOM = "ovrad_random"  # FLOAT in [0, 1), a stable random value per patch (display)
RADIOSITY = "ovrad_radiosity"  # FLOAT_COLOR, solved radiance B/pi
DIRECT = "ovrad_direct"  # FLOAT_COLOR, the first shot's share of it (direct light of lamps and emitters)
# INT, 1 where bake points and near gather hits cast sky rays (radiosity.emission.bake_sky), by Solve
SKY = "ovrad_sky"
# INT, with the kept C only: the contact flags C was integrated with (overlap.contacts.contact_flags: 1 cut,
# 2 whole, 4 covered), so a solve whose kept C fits need not find the contacts again
CONTACTS = "ovrad_contacts"

# EDGE attribute on an atlas object: one edge between each two overlapping patches (overlap/kept.py).
OVERLAP_C = "ovrad_c"  # FLOAT2, (C[i, j], C[j, i]) of the edge's vertices i < j (overlap_matrix's C)

# Custom properties on the atlas object.
PROP_SOURCE = "ovrad_source"  # name of the source mesh object
PROP_BETA = "ovrad_beta"  # beta profile the atlas was built with ("box" or "smooth")
PROP_VERSION = "ovrad_atlas_version"
PROP_LIGHT_KEY = "ovrad_light_key"  # hash of the lamps and emission the stored solve used
# transport rays of the stored solve that left the scene (0: closed, the bakes leave the sky out)
PROP_ESCAPED = "ovrad_escaped"
PROP_ENVIRONMENT = "ovrad_environment_key"  # on the environment atlas: fingerprint of its surfaces
# On an atlas object's mesh: the key of the overlaps kept on its edges (overlap.kept.overlap_key).
PROP_OVERLAP_KEY = "ovrad_overlap_key"
# ... and the quadrature they were integrated with (AtlasSettings.rule_order; absent: 12).
PROP_OVERLAP_QUADRATURE = "ovrad_overlap_quadrature"

IMAGE_SUFFIX = "_ovrad"  # an image bake of object X is the image data block X + IMAGE_SUFFIX
LIGHTMAP_UV = "ovrad_lightmap"  # the UV map an image bake makes where a mesh has none fit for a lightmap
PROP_LIGHTMAP_UV = "ovrad_lightmap_uv"  # on that mesh: digest of the UV map ovrad made (only it is replaced)
PROP_LIGHTMAP_IMAGE = "ovrad_lightmap_image"  # on an object: the image its last image bake wrote it to
PROP_LIGHTMAP_UV_MAP = "ovrad_lightmap_uv_map"  # ... and the UV map that bake went through
PROP_EXPOSURE = "ovrad_exposure"  # on a 16-bit PNG bake's image: its values are v / 65535 x 2^exposure

COLLECTION = "ovrad"
ENVIRONMENT = "ovrad_environment"  # the atlas object of every rendered mesh without an atlas
DISPLAY_NODE_GROUP = "ovrad_patch_display"
DISPLAY_MODIFIER = "ovrad display"

SHAPE_DISK = 0
SHAPE_SQUARE = 1
SHAPE_BALL = 2  # holds the points of small pieces within its radius (clutter.py)
