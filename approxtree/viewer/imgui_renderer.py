"""ImguiRenderer: Dear ImGui (imgui-bundle) drawn with moderngl into the viewer's window.

imgui-bundle ships glfw/OpenGL backends for Python, but they need PyOpenGL; the viewer already
owns a moderngl context, so this module draws imgui's draw lists with it (one program, one
streamed vertex/index buffer, scissor per command) and uploads imgui's textures (the font
atlas, created and updated by imgui ≥ 1.92 through ``ImTextureData``) as moderngl textures.
Input is fed by the viewer's own glfw callbacks (``mouse``, ``button``, ``wheel``), so
scripted runs drive the UI through the same calls.
"""

from __future__ import annotations

from typing import Any

import numpy as np

_VERTEX = """
#version 330
uniform mat4 u_projection;
in vec2 in_pos;
in vec2 in_uv;
in vec4 in_colour;
out vec2 v_uv;
out vec4 v_colour;
void main() {
    v_uv = in_uv;
    v_colour = in_colour;
    gl_Position = u_projection * vec4(in_pos, 0.0, 1.0);
}
"""

_FRAGMENT = """
#version 330
uniform sampler2D u_texture;
in vec2 v_uv;
in vec4 v_colour;
out vec4 out_colour;
void main() {
    out_colour = v_colour * texture(u_texture, v_uv);
}
"""


class ImguiRenderer:
    """Owns one imgui context and draws its frames into ``ctx`` (a moderngl context)."""

    def __init__(self, ctx: Any, size: tuple[int, int]) -> None:
        from imgui_bundle import imgui

        self.imgui = imgui
        self.ctx = ctx
        self.context = imgui.create_context()
        imgui.set_current_context(self.context)
        io = self.io = imgui.get_io()
        # No imgui.ini next to the user's files; the viewer lays its windows out itself.
        io.set_ini_filename("")
        io.display_size = imgui.ImVec2(*size)
        # Textures are ours (the font atlas); no vertex offsets, so imgui splits draw lists
        # that outgrow 16-bit indices instead (moderngl draws without a base vertex).
        io.backend_flags |= imgui.BackendFlags_.renderer_has_textures
        limit = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 4096))
        pio = imgui.get_platform_io()
        pio.renderer_texture_max_width = limit
        pio.renderer_texture_max_height = limit
        self.program = ctx.program(vertex_shader=_VERTEX, fragment_shader=_FRAGMENT)
        self.vbo = ctx.buffer(reserve=1 << 16, dynamic=True)
        self.ibo = ctx.buffer(reserve=1 << 16, dynamic=True)
        self.vao = ctx.vertex_array(
            self.program,
            [(self.vbo, "2f 2f 4f1", "in_pos", "in_uv", "in_colour")],
            index_buffer=self.ibo,
            index_element_size=imgui.INDEX_SIZE,
        )
        self.textures: dict[int, Any] = {}

    # -- input (window coordinates, y down) --------------------------------------------------

    def mouse(self, x: float, y: float) -> None:
        self.io.add_mouse_pos_event(float(x), float(y))

    def button(self, index: int, down: bool) -> None:
        self.io.add_mouse_button_event(int(index), bool(down))

    def wheel(self, dx: float, dy: float) -> None:
        self.io.add_mouse_wheel_event(float(dx), float(dy))

    @property
    def wants_mouse(self) -> bool:
        """True while the pointer is over an imgui window (the map must not react)."""
        return bool(self.io.want_capture_mouse)

    # -- frames -------------------------------------------------------------------------------

    def new_frame(self, size: tuple[int, int], dt: float) -> None:
        imgui = self.imgui
        imgui.set_current_context(self.context)
        self.io.display_size = imgui.ImVec2(*size)
        self.io.delta_time = max(float(dt), 1e-4)
        imgui.new_frame()

    def render(self, viewport: tuple[int, int]) -> None:
        """End the imgui frame and draw it into the bound framebuffer (``viewport`` px)."""
        imgui = self.imgui
        imgui.render()
        data = imgui.get_draw_data()
        self._update_textures()
        w, h = viewport
        dw, dh = self.io.display_size.x, self.io.display_size.y
        if w == 0 or h == 0 or dw == 0 or dh == 0:
            return
        sx, sy = w / dw, h / dh
        proj = np.array(
            [
                [2.0 / dw, 0.0, 0.0, -1.0],
                [0.0, -2.0 / dh, 0.0, 1.0],
                [0.0, 0.0, -1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            dtype="f4",
        )
        self.program["u_projection"].write(proj.T.tobytes())
        self.program["u_texture"].value = 0
        ctx = self.ctx
        vsize, isize = imgui.VERTEX_SIZE, imgui.INDEX_SIZE
        with ctx.scope(enable_only=ctx.BLEND):
            ctx.blend_func = ctx.SRC_ALPHA, ctx.ONE_MINUS_SRC_ALPHA
            ctx.viewport = (0, 0, w, h)
            for commands in data.cmd_lists:
                vbytes = commands.vtx_buffer.size() * vsize
                ibytes = commands.idx_buffer.size() * isize
                self._fit(vbytes, ibytes)
                self.vbo.write(_read(commands.vtx_buffer.data_address(), vbytes))
                self.ibo.write(_read(commands.idx_buffer.data_address(), ibytes))
                for cmd in commands.cmd_buffer:
                    tex = self.textures.get(int(cmd.tex_ref.get_tex_id()))
                    if tex is not None:
                        tex.use(location=0)
                    x0, y0, x1, y1 = cmd.clip_rect
                    ctx.scissor = (
                        int(x0 * sx),
                        int(h - y1 * sy),
                        int((x1 - x0) * sx),
                        int((y1 - y0) * sy),
                    )
                    self.vao.render(
                        ctx.TRIANGLES,
                        vertices=cmd.elem_count,
                        first=cmd.idx_offset,
                    )
            ctx.scissor = None

    def _fit(self, vbytes: int, ibytes: int) -> None:
        # Grow the streamed buffers (rebuilding the vertex array) when a frame needs more.
        if vbytes <= self.vbo.size and ibytes <= self.ibo.size:
            return
        if vbytes > self.vbo.size:
            self.vbo.orphan(max(vbytes, 2 * self.vbo.size))
        if ibytes > self.ibo.size:
            self.ibo.orphan(max(ibytes, 2 * self.ibo.size))

    def _update_textures(self) -> None:
        imgui = self.imgui
        status = imgui.ImTextureStatus
        for tex in imgui.get_platform_io().textures:
            if tex.status == status.want_create or tex.status == status.want_updates:
                pixels = np.asarray(tex.get_pixels_array(), dtype=np.uint8)
                key = int(tex.tex_id)
                old = self.textures.get(key)
                if tex.status == status.want_create or old is None:
                    t = self.ctx.texture((tex.width, tex.height), 4, pixels.tobytes())
                    t.filter = (self.ctx.LINEAR, self.ctx.LINEAR)
                    t.repeat_x = t.repeat_y = False
                    self.textures[t.glo] = t
                    tex.set_tex_id(t.glo)
                else:
                    old.write(pixels.tobytes())
                tex.status = status.ok
            elif tex.status == status.want_destroy:
                t = self.textures.pop(int(tex.tex_id), None)
                if t is not None:
                    t.release()
                tex.set_tex_id(0)
                tex.status = status.destroyed

    def release(self) -> None:
        for t in self.textures.values():
            t.release()
        self.textures.clear()
        self.vao.release()
        self.vbo.release()
        self.ibo.release()
        self.program.release()
        self.imgui.destroy_context(self.context)


def _read(address: int, nbytes: int) -> bytes:
    """``nbytes`` bytes at a native ``address`` (imgui's vertex and index arrays)."""
    import ctypes

    return ctypes.string_at(address, nbytes)
