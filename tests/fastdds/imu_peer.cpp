// A Fast DDS peer of the imu-fsda node, as a ROS 2 stack on rmw_fastrtps meets it: Debian's
// Fast DDS 2.9 (libfastrtps), ROS 2's DDS names (rt/<topic>, sensor_msgs::msg::dds_::Imu_), the
// sensor-data QoS a driver publishes with (best effort, volatile, keep last 5) and a reliable
// reader of the node's output. No ROS 2 library and no code of the node: the message layout is
// written here from sensor_msgs/msg/Imu.msg (CDR, XCDR1 little endian), the service mapping
// from rmw_fastrtps's (request id as the related sample identity).
//
//   imu_peer --csv EUROC_IMU_CSV --count N --rate HZ --after-match-s S --out FILE
//            [--wait-for both|writer] [--adapt-node NAME --adapt-at K] [--security DIR]
//
// With --security, the participant runs DDS Security's builtin plugins (PKI-DH authentication,
// permissions access control, AES-GCM-GMAC crypto) on the files of an SROS2 enclave folder
// DIR, with the property names rmw_fastrtps sets. With --send-unmatched 1, it publishes (and
// calls) after the match timeout all the same, as a stranger on the domain would try.
//
// With --adapt-node, calls NAME's ~/adapt (std_srvs/Trigger) after the K-th sample, as
// rmw_fastrtps's client does: rq/NAME/adaptRequest written with the related sample identity's
// writer GUID set to the client's reply reader, the request's own sample identity kept as its
// id, and a reply taken when its related sample identity names the client (reader or writer
// GUID) and that sequence number.
//
// Publishes rows of an EuRoC imu0/data.csv (ns, ω xyz, a xyz) on rt/imu/data_raw once its
// writer and reader are matched (and S seconds more; 0: at once, the moment a robot's driver
// would), keeps reading rt/imu/denoised until `count` arrived or 3 s pass without one, then
// writes FILE: a first line of key=value pairs, then one line per /imu/denoised:
// stamp_ns frame_id and the message's 37 doubles as their IEEE-754 bits (hex), in field order.

#include <fastcdr/Cdr.h>
#include <fastcdr/FastBuffer.h>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/common/WriteParams.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

using namespace eprosima::fastdds::dds;
using eprosima::fastcdr::Cdr;
using eprosima::fastcdr::FastBuffer;
using eprosima::fastrtps::rtps::SerializedPayload_t;
using eprosima::fastrtps::rtps::InstanceHandle_t;

// ---- the messages, laid out as rosidl's DDS types ----------------------------------------

struct Imu {
    int32_t sec = 0;
    uint32_t nanosec = 0;
    std::string frame_id;
    std::array<double, 37> values{};  // orientation 4, cov 9, ω 3, cov 9, a 3, cov 9
};

struct TriggerRequest {
    uint8_t structure_needs_at_least_one_member = 0;
};

struct TriggerResponse {
    bool success = false;
    std::string message;
};

// One TopicDataType for a struct with `write(Cdr&)` and `read(Cdr&)`: the encapsulation
// header, then the fields.
template <typename T>
class Type : public TopicDataType {
  public:
    using Write = std::function<void(Cdr&, const T&)>;
    using Read = std::function<void(Cdr&, T&)>;
    Type(const char* name, uint32_t max_size, Write w, Read r) : write_(std::move(w)), read_(std::move(r)) {
        setName(name);
        m_typeSize = max_size;
        m_isGetKeyDefined = false;
    }
    bool serialize(void* data, SerializedPayload_t* payload) override {
        FastBuffer buffer(reinterpret_cast<char*>(payload->data), payload->max_size);
        Cdr ser(buffer, Cdr::DEFAULT_ENDIAN, Cdr::DDS_CDR);
        payload->encapsulation = ser.endianness() == Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
        try {
            ser.serialize_encapsulation();
            write_(ser, *static_cast<T*>(data));
        } catch (...) {
            return false;
        }
        payload->length = static_cast<uint32_t>(ser.getSerializedDataLength());
        return true;
    }
    bool deserialize(SerializedPayload_t* payload, void* data) override {
        FastBuffer buffer(reinterpret_cast<char*>(payload->data), payload->length);
        Cdr deser(buffer, Cdr::DEFAULT_ENDIAN, Cdr::DDS_CDR);
        try {
            deser.read_encapsulation();
            payload->encapsulation = deser.endianness() == Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
            read_(deser, *static_cast<T*>(data));
        } catch (...) {
            return false;
        }
        return true;
    }
    std::function<uint32_t()> getSerializedSizeProvider(void*) override {
        uint32_t n = m_typeSize;
        return [n]() { return n; };
    }
    void* createData() override { return new T(); }
    void deleteData(void* data) override { delete static_cast<T*>(data); }
    bool getKey(void*, InstanceHandle_t*, bool) override { return false; }

  private:
    Write write_;
    Read read_;
};

static TypeSupport imu_type() {
    return TypeSupport(new Type<Imu>(
        "sensor_msgs::msg::dds_::Imu_", 4 + 8 + 4 + 256 + 8 + 37 * 8,
        [](Cdr& c, const Imu& m) {
            c << m.sec << m.nanosec << m.frame_id;
            for (double v : m.values) c << v;
        },
        [](Cdr& c, Imu& m) {
            c >> m.sec >> m.nanosec >> m.frame_id;
            for (double& v : m.values) c >> v;
        }));
}

static TypeSupport trigger_request_type() {
    return TypeSupport(new Type<TriggerRequest>(
        "std_srvs::srv::dds_::Trigger_Request_", 4 + 1,
        [](Cdr& c, const TriggerRequest& m) { c << m.structure_needs_at_least_one_member; },
        [](Cdr& c, TriggerRequest& m) { c >> m.structure_needs_at_least_one_member; }));
}

static TypeSupport trigger_response_type() {
    return TypeSupport(new Type<TriggerResponse>(
        "std_srvs::srv::dds_::Trigger_Response_", 4 + 1 + 3 + 4 + 4096,
        [](Cdr& c, const TriggerResponse& m) { c << m.success << m.message; },
        [](Cdr& c, TriggerResponse& m) { c >> m.success >> m.message; }));
}

// ---- the listeners that count matches ------------------------------------------------------

struct WriterMatch : DataWriterListener {
    std::atomic<int> matched{0};
    void on_publication_matched(DataWriter*, const PublicationMatchedStatus& s) override { matched = s.current_count; }
};
struct ReaderMatch : DataReaderListener {
    std::atomic<int> matched{0};
    void on_subscription_matched(DataReader*, const SubscriptionMatchedStatus& s) override { matched = s.current_count; }
};

// ---- input ---------------------------------------------------------------------------------

struct Row {
    int64_t stamp_ns;
    double gyro[3];
    double accel[3];
};

static std::vector<Row> read_csv(const std::string& path, size_t count) {
    std::ifstream f(path);
    std::vector<Row> rows;
    std::string line;
    while (rows.size() < count && std::getline(f, line)) {
        if (line.empty() || line[0] == '#') continue;
        Row r{};
        char* p = line.data();
        r.stamp_ns = std::strtoll(p, &p, 10);
        for (double* v : {&r.gyro[0], &r.gyro[1], &r.gyro[2], &r.accel[0], &r.accel[1], &r.accel[2]}) {
            while (*p == ',' || *p == ' ') ++p;
            *v = std::strtod(p, &p);  // correctly rounded, as the importer's parse
        }
        rows.push_back(r);
    }
    return rows;
}

static std::string arg(int argc, char** argv, const char* name, const char* fallback) {
    for (int i = 1; i + 1 < argc; ++i)
        if (std::strcmp(argv[i], name) == 0) return argv[i + 1];
    return fallback;
}

static uint64_t bits(double v) {
    uint64_t b;
    std::memcpy(&b, &v, sizeof b);
    return b;
}

int main(int argc, char** argv) {
    const std::string csv = arg(argc, argv, "--csv", "");
    const size_t count = std::stoul(arg(argc, argv, "--count", "2000"));
    const double rate = std::stod(arg(argc, argv, "--rate", "200"));
    const double after_match_s = std::stod(arg(argc, argv, "--after-match-s", "1"));
    const double match_timeout_s = std::stod(arg(argc, argv, "--match-timeout-s", "20"));
    const std::string out_path = arg(argc, argv, "--out", "peer.txt");
    const std::string frame_id = arg(argc, argv, "--frame-id", "imu_link");
    const char* domain_env = std::getenv("ROS_DOMAIN_ID");
    const int domain = domain_env ? std::atoi(domain_env) : 0;

    std::vector<Row> rows = read_csv(csv, count);
    if (rows.size() != count) {
        std::fprintf(stderr, "imu_peer: %s has %zu rows, %zu asked\n", csv.c_str(), rows.size(), count);
        return 2;
    }

    DomainParticipantQos pqos;
    pqos.name("imu_peer");
    const std::string security = arg(argc, argv, "--security", "");
    if (!security.empty()) {
        auto& props = pqos.properties().properties();
        const std::string file = "file://" + security + "/";
        props.emplace_back("dds.sec.auth.plugin", "builtin.PKI-DH");
        props.emplace_back("dds.sec.auth.builtin.PKI-DH.identity_ca", file + "identity_ca.cert.pem");
        props.emplace_back("dds.sec.auth.builtin.PKI-DH.identity_certificate", file + "cert.pem");
        props.emplace_back("dds.sec.auth.builtin.PKI-DH.private_key", file + "key.pem");
        props.emplace_back("dds.sec.access.plugin", "builtin.Access-Permissions");
        props.emplace_back("dds.sec.access.builtin.Access-Permissions.permissions_ca", file + "permissions_ca.cert.pem");
        props.emplace_back("dds.sec.access.builtin.Access-Permissions.governance", file + "governance.p7s");
        props.emplace_back("dds.sec.access.builtin.Access-Permissions.permissions", file + "permissions.p7s");
        props.emplace_back("dds.sec.crypto.plugin", "builtin.AES-GCM-GMAC");
    }
    DomainParticipant* participant = DomainParticipantFactory::get_instance()->create_participant(domain, pqos);
    if (!participant) return 3;
    TypeSupport type = imu_type();
    type.register_type(participant);
    Topic* raw = participant->create_topic("rt/imu/data_raw", type.get_type_name(), TOPIC_QOS_DEFAULT);
    Topic* denoised = participant->create_topic("rt/imu/denoised", type.get_type_name(), TOPIC_QOS_DEFAULT);
    Publisher* pub = participant->create_publisher(PUBLISHER_QOS_DEFAULT);
    Subscriber* sub = participant->create_subscriber(SUBSCRIBER_QOS_DEFAULT);

    // rmw's qos_profile_sensor_data, and rmw_fastrtps's history memory policy.
    DataWriterQos wqos = DATAWRITER_QOS_DEFAULT;
    wqos.reliability().kind = BEST_EFFORT_RELIABILITY_QOS;
    wqos.durability().kind = VOLATILE_DURABILITY_QOS;
    wqos.history().kind = KEEP_LAST_HISTORY_QOS;
    wqos.history().depth = 5;
    wqos.endpoint().history_memory_policy = eprosima::fastrtps::rtps::PREALLOCATED_WITH_REALLOC_MEMORY_MODE;
    WriterMatch wmatch;
    DataWriter* writer = pub->create_datawriter(raw, wqos, &wmatch);

    // The node's output is reliable: a reader that keeps all of it.
    DataReaderQos rqos = DATAREADER_QOS_DEFAULT;
    rqos.reliability().kind = RELIABLE_RELIABILITY_QOS;
    rqos.durability().kind = VOLATILE_DURABILITY_QOS;
    rqos.history().kind = KEEP_ALL_HISTORY_QOS;
    rqos.resource_limits().max_samples = static_cast<int32_t>(count + 100);
    rqos.endpoint().history_memory_policy = eprosima::fastrtps::rtps::PREALLOCATED_WITH_REALLOC_MEMORY_MODE;
    ReaderMatch rmatch;
    DataReader* reader = sub->create_datareader(denoised, rqos, &rmatch);
    if (!writer || !reader) return 4;

    // ~/adapt, mapped as rmw_fastrtps maps a service (reliable, volatile, keep last 10).
    const std::string adapt_node = arg(argc, argv, "--adapt-node", "");
    const size_t adapt_at = std::stoul(arg(argc, argv, "--adapt-at", "0"));
    DataWriter* request_writer = nullptr;
    DataReader* reply_reader = nullptr;
    WriterMatch request_match;
    ReaderMatch reply_match;
    if (!adapt_node.empty()) {
        TypeSupport rq = trigger_request_type();
        TypeSupport rr = trigger_response_type();
        rq.register_type(participant);
        rr.register_type(participant);
        Topic* rq_topic = participant->create_topic("rq/" + adapt_node + "/adaptRequest", rq.get_type_name(), TOPIC_QOS_DEFAULT);
        Topic* rr_topic = participant->create_topic("rr/" + adapt_node + "/adaptReply", rr.get_type_name(), TOPIC_QOS_DEFAULT);
        DataWriterQos q = DATAWRITER_QOS_DEFAULT;
        q.reliability().kind = RELIABLE_RELIABILITY_QOS;
        q.durability().kind = VOLATILE_DURABILITY_QOS;
        q.history().kind = KEEP_LAST_HISTORY_QOS;
        q.history().depth = 10;
        DataReaderQos rq_qos = DATAREADER_QOS_DEFAULT;
        rq_qos.reliability().kind = RELIABLE_RELIABILITY_QOS;
        rq_qos.durability().kind = VOLATILE_DURABILITY_QOS;
        rq_qos.history().kind = KEEP_LAST_HISTORY_QOS;
        rq_qos.history().depth = 10;
        request_writer = pub->create_datawriter(rq_topic, q, &request_match);
        reply_reader = sub->create_datareader(rr_topic, rq_qos, &reply_match);
        if (!request_writer || !reply_reader) return 5;
    }

    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    auto since = [](clock::time_point t) { return std::chrono::duration<double>(clock::now() - t).count(); };
    // A driver publishes once its writer matched (`--wait-for writer`); a test that wants every
    // output back waits for its reader of them too (`both`).
    const bool both = arg(argc, argv, "--wait-for", "both") == "both";
    auto ready = [&]() {
        const bool service = adapt_node.empty() || (request_match.matched >= 1 && reply_match.matched >= 1);
        return wmatch.matched >= 1 && (!both || rmatch.matched >= 1) && service;
    };
    while (!ready() && since(t0) < match_timeout_s) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    const bool matched = ready();
    const double match_s = since(t0);
    if (matched && after_match_s > 0)
        std::this_thread::sleep_for(std::chrono::duration<double>(after_match_s));

    std::vector<Imu> received;
    auto drain = [&]() {
        Imu m;
        SampleInfo info;
        while (reader->take_next_sample(&m, &info) == ReturnCode_t::RETCODE_OK)
            if (info.valid_data) received.push_back(m);
    };
    // The call: its id, and the reply when it comes.
    eprosima::fastrtps::rtps::SampleIdentity request_id;
    bool called = false, replied = false;
    TriggerResponse reply;
    double call_s = 0, reply_s = 0;
    auto call = [&]() {
        eprosima::fastrtps::rtps::WriteParams params;
        params.related_sample_identity().writer_guid() = reply_reader->guid();
        TriggerRequest req;
        if (request_writer->write(&req, params)) {
            request_id = params.sample_identity();
            called = true;
            call_s = since(t0);
        }
    };
    auto take_reply = [&]() {
        if (!reply_reader || replied) return;
        TriggerResponse r;
        SampleInfo info;
        while (reply_reader->take_next_sample(&r, &info) == ReturnCode_t::RETCODE_OK) {
            const auto& related = info.related_sample_identity;
            const bool ours = related.writer_guid() == reply_reader->guid() || related.writer_guid() == request_writer->guid();
            if (info.valid_data && called && ours && related.sequence_number() == request_id.sequence_number()) {
                reply = r;
                replied = true;
                reply_s = since(t0);
            }
        }
    };
    size_t sent = 0;
    const bool send = matched || arg(argc, argv, "--send-unmatched", "0") == "1";
    const auto start = clock::now();
    for (size_t i = 0; send && i < rows.size(); ++i) {
        const Row& r = rows[i];
        Imu m;
        m.sec = static_cast<int32_t>(r.stamp_ns / 1000000000);
        m.nanosec = static_cast<uint32_t>(r.stamp_ns % 1000000000);
        m.frame_id = frame_id;
        m.values.fill(0.0);
        m.values[3] = 1.0;     // orientation w, with orientation_covariance[0] = -1: none
        m.values[4] = -1.0;
        for (int k = 0; k < 3; ++k) {
            m.values[13 + k] = r.gyro[k];
            m.values[25 + k] = r.accel[k];
        }
        if (writer->write(&m)) ++sent;
        if (request_writer && i + 1 == adapt_at) call();
        drain();
        take_reply();
        std::this_thread::sleep_until(start + std::chrono::duration<double>((i + 1) / rate));
    }
    auto last = clock::now();
    while (send && (received.size() < sent || (called && !replied)) && since(last) < 3.0) {
        size_t before = received.size();
        drain();
        take_reply();
        if (received.size() != before) last = clock::now();
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }

    std::ofstream out(out_path);
    out << "matched=" << (matched ? 1 : 0) << " match_s=" << match_s << " reader_matched=" << rmatch.matched.load() << " sent=" << sent
        << " received=" << received.size() << " called=" << called << " replied=" << replied << " call_s=" << call_s
        << " reply_s=" << reply_s << " reply_success=" << reply.success << "\n";
    if (replied) out << "reply_message " << reply.message << "\n";
    char buf[32];
    for (const Imu& m : received) {
        out << (static_cast<int64_t>(m.sec) * 1000000000 + m.nanosec) << ' ' << m.frame_id;
        for (double v : m.values) {
            std::snprintf(buf, sizeof buf, " %016llx", static_cast<unsigned long long>(bits(v)));
            out << buf;
        }
        out << '\n';
    }
    out.close();
    participant->delete_contained_entities();
    DomainParticipantFactory::get_instance()->delete_participant(participant);
    std::fprintf(stderr, "imu_peer: matched %d after %.3f s, sent %zu, received %zu\n", matched ? 1 : 0, match_s, sent, received.size());
    return matched ? 0 : 1;
}
