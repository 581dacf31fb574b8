// ImGui panel (panel.hpp), through Debian's libimgui (its GLFW and OpenGL 3
// backends are part of the library).
#include "view/panel.hpp"

#include <GLFW/glfw3.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <imgui.h>

#include <cstdio>

namespace voxcast::view {

Gui::Gui(GLFWwindow* window) {
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;  // no imgui.ini left in the working directory
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForOpenGL(window, /*install_callbacks=*/true);
  ImGui_ImplOpenGL3_Init("#version 330 core");
}

Gui::~Gui() {
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
}

void Gui::begin_frame() {
  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
}

void Gui::end_frame() {
  ImGui::Render();
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
}

bool Gui::wants_mouse() const {
  return ImGui::GetIO().WantCaptureMouse;
}
bool Gui::wants_keyboard() const {
  return ImGui::GetIO().WantCaptureKeyboard;
}

PanelActions Gui::panel(bool show_panel, const SceneStats& scene, ViewSettings* s, int* max_passes,
                        CameraMode* mode, float* speed, const FrameStatus& st) {
  PanelActions a;
  // Overlay, top left: what a frame costs.
  ImGui::SetNextWindowPos(ImVec2(8, 8));
  ImGui::SetNextWindowBgAlpha(0.5f);
  ImGui::Begin("##stats", nullptr,
               ImGuiWindowFlags_NoDecoration | ImGuiWindowFlags_AlwaysAutoResize |
                   ImGuiWindowFlags_NoInputs | ImGuiWindowFlags_NoSavedSettings |
                   ImGuiWindowFlags_NoFocusOnAppearing | ImGuiWindowFlags_NoNav);
  ImGui::Text("frame %.1f ms  (render %.1f ms)", st.frame_ms, st.render_ms);
  ImGui::Text("%.2f Mrays/s primary, %.2f with effects", st.mrays, st.mrays_total);
  ImGui::Text("%dx%d%s  pass %d/%d", st.width, st.height, st.preview_scale > 1 ? " (preview)" : "",
              st.passes, st.max_passes);
  if (st.recording) ImGui::TextColored(ImVec4(1, 0.3f, 0.3f, 1), "REC %zu", st.recorded_keyframes);
  if (st.playing) ImGui::TextColored(ImVec4(0.4f, 1, 0.4f, 1), "playing path");
  ImGui::End();
  if (!show_panel) return a;

  ImGui::SetNextWindowPos(ImVec2(ImGui::GetIO().DisplaySize.x - 328, 8), ImGuiCond_FirstUseEver);
  ImGui::SetNextWindowSize(ImVec2(320, 0), ImGuiCond_FirstUseEver);
  ImGui::Begin("voxcast view");
  if (ImGui::CollapsingHeader("Structure", ImGuiTreeNodeFlags_DefaultOpen)) {
    for (const auto& [label, value] : scene.rows)
      ImGui::Text("%s: %s", label.c_str(), value.c_str());
  }
  if (ImGui::CollapsingHeader("Render", ImGuiTreeNodeFlags_DefaultOpen)) {
    ImGui::SliderFloat("LOD (pixels)", &s->lod_pixels, 0.f, 16.f, "%.2f");
    static const int beams[] = {0, 4, 8, 16};
    static const char* beam_names[] = {"off", "4x4", "8x8", "16x16"};
    int beam_index = 0;
    for (int i = 0; i < 4; ++i)
      if (beams[i] == s->beam) beam_index = i;
    if (ImGui::Combo("beam", &beam_index, beam_names, 4)) s->beam = beams[beam_index];
    ImGui::Checkbox("shadows (hard)", &s->hard_shadows);
    ImGui::SliderInt("AO rays", &s->ao_rays, 0, 64);
    ImGui::SliderInt("AA samples", &s->spp, 1, 16);
    ImGui::Checkbox("post-filter", &s->filter);
    ImGui::Checkbox("heat map (H)", &s->heatmap);
    if (s->heatmap) ImGui::SliderFloat("heat max", &s->heatmap_max, 1.f, 512.f, "%.0f");
    ImGui::Checkbox("GI (path traced)", &s->gi);
    if (s->gi) {
      ImGui::SliderInt("GI bounces", &s->gi_bounces, 0, 16);
      ImGui::Checkbox("GI sun", &s->gi_sun);
      if (s->gi_environment && s->gi_environment->can_sample())
        ImGui::Checkbox("GI env sampling", &s->gi_env_sampling);
    }
    ImGui::SliderInt("passes", max_passes, 1, 256);
  }
  if (ImGui::CollapsingHeader("Camera", ImGuiTreeNodeFlags_DefaultOpen)) {
    int m = *mode == CameraMode::Orbit ? 0 : 1;
    ImGui::RadioButton("orbit", &m, 0);
    ImGui::SameLine();
    ImGui::RadioButton("fly (Tab)", &m, 1);
    *mode = m == 0 ? CameraMode::Orbit : CameraMode::Fly;
    ImGui::SliderFloat("speed", speed, 1e-4f, 1e4f, "%.3g", ImGuiSliderFlags_Logarithmic);
    const Camera& c = st.camera;
    ImGui::Text("eye    %.3f %.3f %.3f", c.eye.x, c.eye.y, c.eye.z);
    ImGui::Text("target %.3f %.3f %.3f", c.target.x, c.target.y, c.target.z);
    if (ImGui::Button("reframe (F)")) a.reframe = true;
  }
  if (ImGui::CollapsingHeader("Path", ImGuiTreeNodeFlags_DefaultOpen)) {
    if (ImGui::Button(st.recording ? "stop recording (R)" : "record (R)")) a.toggle_record = true;
    ImGui::SameLine();
    if (ImGui::Button("play (P)")) a.play = true;
    if (ImGui::Button("screenshot (F12)")) a.screenshot = true;
  }
  ImGui::End();
  return a;
}

std::string view_library_versions() {
  return std::string("GLFW ") + glfwGetVersionString() + "\nDear ImGui " + IMGUI_VERSION + "\n";
}

}  // namespace voxcast::view
