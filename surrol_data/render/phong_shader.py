"""Per-pixel Phong shading under the endoscope's two spotlights with their shadow maps, as one GLSL program.

Why not Panda3D's ``set_shader_auto()``: its generated shaders are Cg, and NVIDIA's Cg runtime cannot
find a shader profile on an EGL context (Panda3D logs "The profile is not supported" and falls back to
ambient light only) — which is exactly where offscreen observations are rendered. This GLSL program is
what the auto shader would compute for one spotlight, written out, so the window and the offscreen
camera draw the same image with any OpenGL ≥ 3.3 (Mesa's llvmpipe included).

Per fragment: albedo = (colour × material texture) linearised with the display's gamma; per spotlight (the
scope light and the shadow light of :mod:`~surrol_data.render.endoscope_light`), irradiance = colour ×
attenuation(distance) × cone(angle) × shadow × max(n·l, 0) and a Phong highlight = specular × (r·v)^shininess;
plus the ambient term; then a soft shoulder above 0.8 and the display's gamma, as a camera encodes light. The cone edge is softened over the last few degrees (a real fibre bundle's beam has
no hard edge); shadow lookups (the shadow light's only) use the hardware's 2×2 depth comparison (``sampler2DShadow``).
"""

from __future__ import annotations

from panda3d.core import Shader

VERTEX = """
#version 330
uniform mat4 p3d_ModelViewProjectionMatrix;
uniform mat4 p3d_ModelViewMatrix;
uniform mat3 p3d_NormalMatrix;
uniform mat4 p3d_TextureMatrix;
in vec4 p3d_Vertex;
in vec3 p3d_Normal;
in vec2 p3d_MultiTexCoord0;
out vec3 v_position;   // view space
out vec3 v_normal;     // view space
out vec2 v_uv;
void main() {
    gl_Position = p3d_ModelViewProjectionMatrix * p3d_Vertex;
    v_position = vec3(p3d_ModelViewMatrix * p3d_Vertex);
    v_normal = normalize(p3d_NormalMatrix * p3d_Normal);
    v_uv = (p3d_TextureMatrix * vec4(p3d_MultiTexCoord0, 0.0, 1.0)).xy;
}
"""

FRAGMENT = """
#version 330
uniform struct p3d_LightSourceParameters {
    vec4 color;
    vec4 position;
    vec3 spotDirection;
    float spotExponent;
    float spotCosCutoff;
    vec3 attenuation;
    sampler2DShadow shadowMap;
    mat4 shadowViewMatrix;
} p3d_LightSource[2];
uniform struct { vec4 ambient; } p3d_LightModel;
uniform struct p3d_MaterialParameters {
    vec4 diffuse;
    vec3 specular;
    float shininess;
} p3d_Material;
uniform vec4 p3d_ColorScale;
uniform sampler2D p3d_Texture0;
uniform float u_shadows;   // 1: look the shadow maps up; 0: no shadows
in vec3 v_position;
in vec3 v_normal;
in vec2 v_uv;
out vec4 o_color;

const int SHADOW_LIGHT = 1;          // the light that casts shadows (endoscope_light orders them by priority)
const float CONE_SOFT_EDGE = 0.06;   // in cos(angle): about the last 5 degrees of the cone
const float GAMMA = 2.2;             // the display's: colours are sRGB-like, light adds up linearly
const float KNEE = 0.8;              // above it, a soft shoulder instead of clipping to white

vec3 spot_light(int i, vec3 n, vec3 v, vec3 albedo) {
    vec3 to_light = p3d_LightSource[i].position.xyz - v_position;
    float d = length(to_light);
    vec3 l = to_light / d;
    float cos_angle = dot(-l, normalize(p3d_LightSource[i].spotDirection));
    float cutoff = p3d_LightSource[i].spotCosCutoff;
    float cone = smoothstep(cutoff, cutoff + CONE_SOFT_EDGE, cos_angle)
                 * pow(max(cos_angle, 0.0), p3d_LightSource[i].spotExponent);
    vec3 att = p3d_LightSource[i].attenuation;
    float falloff = 1.0 / max(att.x + att.y * d + att.z * d * d, 1e-6);
    float lit = 1.0;
    // Only the shadow light's map is read: the scope light's is a dummy that reads lit, and a lookup costs about an
    // eighth of a frame on a software rasteriser (Mesa's llvmpipe).
    if (i == SHADOW_LIGHT && u_shadows > 0.5) {
        vec4 shadow_coord = p3d_LightSource[i].shadowViewMatrix * vec4(v_position, 1.0);
        lit = textureProj(p3d_LightSource[i].shadowMap, shadow_coord);
    }
    vec3 radiance = p3d_LightSource[i].color.rgb * falloff * cone * lit;
    float n_dot_l = max(dot(n, l), 0.0);
    vec3 colour = albedo * radiance * n_dot_l;
    if (n_dot_l > 0.0) {
        vec3 r = reflect(-l, n);
        colour += p3d_Material.specular.rgb * radiance * pow(max(dot(r, v), 0.0), p3d_Material.shininess);
    }
    return colour;
}

void main() {
    vec4 base = p3d_Material.diffuse * p3d_ColorScale;
    vec3 albedo = pow(base.rgb * texture(p3d_Texture0, v_uv).rgb, vec3(GAMMA));
    vec3 n = normalize(v_normal);
    vec3 v = normalize(-v_position);
    if (dot(n, v) < 0.0) n = -n;   // thin shapes seen from behind
    vec3 colour = p3d_LightModel.ambient.rgb * albedo;
    colour += spot_light(0, n, v, albedo);
    colour += spot_light(1, n, v, albedo);
    // The camera's response: a soft shoulder on the brightest channel (keeping the hue, so a near green
    // sphere stays green instead of burning white), then the display's gamma.
    float peak = max(max(colour.r, colour.g), colour.b);
    if (peak > KNEE) {
        float shoulder = KNEE + (1.0 - KNEE) * (1.0 - exp(-(peak - KNEE) / (1.0 - KNEE)));
        colour *= shoulder / peak;
    }
    o_color = vec4(pow(clamp(colour, 0.0, 1.0), vec3(1.0 / GAMMA)), base.a);
}
"""


def phong_shader() -> Shader:
    return Shader.make(Shader.SL_GLSL, VERTEX, FRAGMENT)


# The shadow light's camera only needs depth: this program replaces the Phong shading there. Panda3D's shadow camera
# turns colour writes off but still runs the scene's shader on every fragment of its map, and on a software
# rasteriser (Mesa's llvmpipe) that pass cost about a fifth of a GUI frame's CPU (measured A/B in one process).
DEPTH_VERTEX = """
#version 330
uniform mat4 p3d_ModelViewProjectionMatrix;
in vec4 p3d_Vertex;
void main() {
    gl_Position = p3d_ModelViewProjectionMatrix * p3d_Vertex;
}
"""

DEPTH_FRAGMENT = """
#version 330
out vec4 o_color;
void main() {
    o_color = vec4(1.0);
}
"""


def depth_only_shader() -> Shader:
    return Shader.make(Shader.SL_GLSL, DEPTH_VERTEX, DEPTH_FRAGMENT)
