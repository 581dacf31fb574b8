#pragma once
// Small value types shared by every module. Floats for geometry that reaches
// the renderer; the builders and generators do their arithmetic in double
// (Vec3d, the same template).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>

namespace voxcast {

struct Vec2 {
  float x = 0, y = 0;
};

/// A 3-vector of float (geometry that reaches the renderer: `Vec3`) or double
/// (the builders' and generators' internal arithmetic: `Vec3d`). One template
/// so that every module shares the same operators; the scalar argument of
/// `v * s` and `v / s` is not deduced, so `Vec3 * 0.5` keeps converting the
/// literal to float as the float-only type did.
template <class T>
struct Vec3T {
  T x = 0, y = 0, z = 0;
  constexpr Vec3T() = default;
  constexpr Vec3T(T x_, T y_, T z_) : x(x_), y(y_), z(z_) {}
  constexpr T operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  constexpr T& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
};
using Vec3 = Vec3T<float>;
using Vec3d = Vec3T<double>;

template <class T>
using Scalar = std::type_identity_t<T>;

template <class T>
constexpr Vec3T<T> operator+(Vec3T<T> a, Vec3T<T> b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
template <class T>
constexpr Vec3T<T> operator-(Vec3T<T> a, Vec3T<T> b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <class T>
constexpr Vec3T<T> operator-(Vec3T<T> a) {
  return {-a.x, -a.y, -a.z};
}
template <class T>
constexpr Vec3T<T> operator*(Vec3T<T> a, Scalar<T> s) {
  return {a.x * s, a.y * s, a.z * s};
}
template <class T>
constexpr Vec3T<T> operator*(Scalar<T> s, Vec3T<T> a) {
  return {a.x * s, a.y * s, a.z * s};
}
template <class T>
constexpr Vec3T<T> operator*(Vec3T<T> a, Vec3T<T> b) {
  return {a.x * b.x, a.y * b.y, a.z * b.z};
}
template <class T>
constexpr Vec3T<T> operator/(Vec3T<T> a, Scalar<T> s) {
  return {a.x / s, a.y / s, a.z / s};
}
template <class T>
constexpr Vec3T<T>& operator+=(Vec3T<T>& a, Vec3T<T> b) {
  return a = a + b;
}
template <class T>
constexpr Vec3T<T>& operator-=(Vec3T<T>& a, Vec3T<T> b) {
  return a = a - b;
}
template <class T>
constexpr Vec3T<T>& operator*=(Vec3T<T>& a, Scalar<T> s) {
  return a = a * s;
}
template <class T>
constexpr T dot(Vec3T<T> a, Vec3T<T> b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
template <class T>
constexpr Vec3T<T> cross(Vec3T<T> a, Vec3T<T> b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
template <class T>
inline T length(Vec3T<T> a) {
  return std::sqrt(dot(a, a));
}
/// a / |a|, or the zero vector for a zero (or non-finite-length) input.
template <class T>
inline Vec3T<T> normalize(Vec3T<T> a) {
  T l = length(a);
  return l > 0 ? a / l : Vec3T<T>{0, 0, 0};
}
template <class T>
constexpr Vec3T<T> min(Vec3T<T> a, Vec3T<T> b) {
  return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
template <class T>
constexpr Vec3T<T> max(Vec3T<T> a, Vec3T<T> b) {
  return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}
template <class T>
inline bool is_finite(Vec3T<T> a) {
  return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z);
}

/// Linear RGBA color with components in [0,1].
struct Color {
  float r = 0, g = 0, b = 0, a = 1;
};

struct Aabb {
  Vec3 lo{INFINITY, INFINITY, INFINITY};
  Vec3 hi{-INFINITY, -INFINITY, -INFINITY};
  void extend(Vec3 p) {
    lo = min(lo, p);
    hi = max(hi, p);
  }
  bool empty() const { return !(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z); }
  Vec3 extent() const { return hi - lo; }
  Vec3 center() const { return (lo + hi) * 0.5f; }
};

/// A ray with a unit (or at least non-zero) direction and an open interval [0, tmax].
struct Ray {
  Vec3 origin;
  Vec3 dir;
  float tmax = INFINITY;
};

}  // namespace voxcast
