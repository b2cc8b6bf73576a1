#version 330 core
// Lambert shading of the base colour under pyrender's directional lights plus ambient light.
struct DirectionalLight {
    vec3 color;
    float intensity;
    vec3 direction;
};
struct Material {
#ifdef USE_METALLIC_MATERIAL
    vec4 base_color_factor;
#endif
#ifdef USE_GLOSSY_MATERIAL
    vec4 diffuse_factor;
#endif
#ifdef HAS_BASE_COLOR_TEX
    sampler2D base_color_texture;
#endif
#ifdef HAS_DIFFUSE_TEX
    sampler2D diffuse_texture;
#endif
};

uniform Material material;
uniform DirectionalLight directional_lights[MAX_DIRECTIONAL_LIGHTS];
uniform int n_directional_lights;
uniform vec3 ambient_light;
uniform vec3 cam_pos;

in vec3 world_position;
in vec3 world_normal;
in vec2 uv;
in vec4 vertex_color;

out vec4 frag_color;

void main()
{
    vec4 base = vertex_color;
#ifdef USE_METALLIC_MATERIAL
    base *= material.base_color_factor;
#endif
#ifdef USE_GLOSSY_MATERIAL
    base *= material.diffuse_factor;
#endif
#ifdef HAS_BASE_COLOR_TEX
    base *= texture(material.base_color_texture, uv);
#endif
#ifdef HAS_DIFFUSE_TEX
    base *= texture(material.diffuse_texture, uv);
#endif
    vec3 n = world_normal;
    // Scanned meshes often have inconsistent winding: light the side that faces the camera.
    if (dot(n, cam_pos - world_position) < 0.0) {
        n = -n;
    }
    vec3 light = ambient_light;
    for (int i = 0; i < n_directional_lights; i++) {
        float lambert = max(dot(n, -directional_lights[i].direction), 0.0);
        light += directional_lights[i].color * directional_lights[i].intensity * lambert;
    }
    frag_color = vec4(clamp(base.rgb * light, 0.0, 1.0), 1.0);
}
