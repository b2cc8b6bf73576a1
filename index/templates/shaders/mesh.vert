#version 330 core
// posedesc's template shader: per-vertex colour or texture, Lambert lighting, nothing else.
// pyrender's default is a full PBR shader, several times slower on Mesa's software rasteriser.
layout(location = 0) in vec3 position;
#ifdef NORMAL_LOC
layout(location = NORMAL_LOC) in vec3 normal;
#endif
#ifdef TEXCOORD_0_LOC
layout(location = TEXCOORD_0_LOC) in vec2 texcoord_0;
#endif
#ifdef COLOR_0_LOC
layout(location = COLOR_0_LOC) in vec4 color_0;
#endif
layout(location = INST_M_LOC) in mat4 inst_m;

uniform mat4 M;
uniform mat4 V;
uniform mat4 P;

out vec3 world_position;
out vec3 world_normal;
out vec2 uv;
out vec4 vertex_color;

void main()
{
    mat4 model = M * inst_m;
    vec4 world = model * vec4(position, 1.0);
    gl_Position = P * V * world;
    world_position = world.xyz;
#ifdef NORMAL_LOC
    // Object poses are rigid, so the model matrix turns normals too (no per-vertex inverse).
    world_normal = normalize(mat3(model) * normal);
#else
    world_normal = vec3(0.0);
#endif
#ifdef TEXCOORD_0_LOC
    uv = texcoord_0;
#else
    uv = vec2(0.0);
#endif
#ifdef COLOR_0_LOC
    vertex_color = color_0;
#else
    vertex_color = vec4(1.0);
#endif
}
